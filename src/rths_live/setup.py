"""Python package set-up of rths_live (ament_python)."""

from setuptools import find_packages, setup

package_name = 'rths_live'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/foxglove',
         ['foxglove/rths_live.json', 'foxglove/rths_live_2_actuators.json']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='rths maintainers',
    maintainer_email='maintainers@rths.dev',
    description=open('package.xml').read().split('<description>')[1].split('</description>')[0],
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'live_view = rths_live.live:main',
        ],
    },
)
